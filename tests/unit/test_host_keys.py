"""A run's keys for TLS between hosts (uav_flock_tools/keys.py, `uav-flock keys`): made once, checked before any process starts, and
accepted by a real TLS stack for mutual verification."""
from __future__ import annotations

import datetime
import shutil
import socket
import ssl
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from uav_flock_tools import keys


def test_every_host_gets_the_ca_its_certificate_and_a_key_only_it_reads(tmp_path: Path) -> None:
    out = tmp_path / 'keys'
    ca = keys.make(out, ['world', 'field1'])
    assert sorted(p.name for p in out.iterdir()) == ['field1', 'world']
    for host in ('world', 'field1'):
        folder = out / host
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        assert stat.S_IMODE((folder / keys.KEY_FILE).stat().st_mode) == 0o600
        held = keys.check(folder, host)
        assert held.host == host and held.ca_fingerprint == keys.fingerprint(ca)
    assert b'PRIVATE KEY' not in b''.join(p.read_bytes() for p in out.rglob('*.pem') if p.name != keys.KEY_FILE), \
        "the CA's private key is never written"


def test_keys_are_never_overwritten_unless_asked(tmp_path: Path) -> None:
    out = tmp_path / 'keys'
    first = keys.make(out, ['a', 'b'])
    with pytest.raises(keys.KeysError, match='--replace'):
        keys.make(out, ['a'])
    assert keys.check(out / 'a').ca_fingerprint == keys.fingerprint(first)
    second = keys.make(out, ['a'], replace=True)
    assert sorted(p.name for p in out.iterdir()) == ['a'], "b's keys, from the old CA, are gone too"
    assert keys.check(out / 'a').ca_fingerprint == keys.fingerprint(second) != keys.fingerprint(first)
    (out / 'notes.txt').write_text('mine')
    with pytest.raises(keys.KeysError, match='not a host folder'):
        keys.make(out, ['a'], replace=True)
    assert (out / 'notes.txt').read_text() == 'mine'


def test_a_folder_that_cannot_secure_a_host_is_named_in_one_line(tmp_path: Path) -> None:
    now = datetime.datetime.now(datetime.timezone.utc)
    keys.make(tmp_path / 'run', ['a', 'b'])
    keys.make(tmp_path / 'other', ['a'])
    keys.make(tmp_path / 'old', ['a'], days=1, now=now - datetime.timedelta(days=3))
    with pytest.raises(keys.KeysError, match='no such folder'):
        keys.check(tmp_path / 'missing')
    with pytest.raises(keys.KeysError, match='expired on'):
        keys.check(tmp_path / 'old' / 'a', 'a')
    with pytest.raises(keys.KeysError, match='not for b'):
        keys.check(tmp_path / 'run' / 'a', 'b')
    mixed = tmp_path / 'mixed'
    shutil.copytree(tmp_path / 'run' / 'a', mixed)
    shutil.copy(tmp_path / 'other' / 'a' / keys.CA_FILE, mixed / keys.CA_FILE)
    with pytest.raises(keys.KeysError, match='not signed by the CA'):
        keys.check(mixed, 'a')
    shutil.copy(tmp_path / 'run' / 'a' / keys.CA_FILE, mixed / keys.CA_FILE)
    shutil.copy(tmp_path / 'run' / 'b' / keys.KEY_FILE, mixed / keys.KEY_FILE)
    with pytest.raises(keys.KeysError, match='not the key of'):
        keys.check(mixed, 'a')
    (mixed / keys.KEY_FILE).unlink()
    with pytest.raises(keys.KeysError, match='key.pem'):
        keys.check(mixed, 'a')


def _context(folder: Path, side: ssl._SSLMethod) -> ssl.SSLContext:
    ctx = ssl.SSLContext(side)
    ctx.load_cert_chain(folder / keys.CERT_FILE, folder / keys.KEY_FILE)
    ctx.load_verify_locations(folder / keys.CA_FILE)
    ctx.verify_mode = ssl.CERT_REQUIRED  # mutual: the dialled side asks for the dialler's certificate too
    ctx.check_hostname = False
    return ctx


def _handshake(server: Path, client: Path) -> str:
    """A TLS handshake between two hosts' folders over a socket pair: 'ok', or what the server saw fail."""
    a, b = socket.socketpair()
    said: list[str] = []

    def serve() -> None:
        try:
            with _context(server, ssl.PROTOCOL_TLS_SERVER).wrap_socket(a, server_side=True) as s:
                said.append('ok' if s.getpeercert() else 'no peer certificate')
        except (ssl.SSLError, OSError) as exc:
            said.append(type(exc).__name__ + ': ' + str(exc))

    t = threading.Thread(target=serve)
    t.start()
    try:
        with _context(client, ssl.PROTOCOL_TLS_CLIENT).wrap_socket(b) as s:
            s.sendall(b'x')
    except (ssl.SSLError, OSError):
        pass
    t.join(10)
    return said[0]


def test_two_hosts_of_a_run_verify_each_other_and_a_stranger_is_refused(tmp_path: Path) -> None:
    keys.make(tmp_path / 'run', ['world', 'field1'])
    keys.make(tmp_path / 'stranger', ['field1'])
    assert _handshake(tmp_path / 'run' / 'world', tmp_path / 'run' / 'field1') == 'ok'
    refused = _handshake(tmp_path / 'run' / 'world', tmp_path / 'stranger' / 'field1')
    assert refused.startswith('SSLError') and ('unknown ca' in refused or 'certificate' in refused), refused


@pytest.mark.parametrize('args, says', [
    (('--hosts', 'a,a'), '--hosts: a is named twice'),
    (('--hosts', 'a/b'), "--hosts: 'a/b' is not a host name"),
    (('--hosts', ','), '--hosts: name at least one host'),
    (('--hosts', 'a', '--days', '0'), '--days: 0'),
])
def test_a_mistake_is_one_line_and_exit_2_and_writes_nothing(tmp_path: Path, args: tuple[str, ...], says: str) -> None:
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'keys', '--out', str(tmp_path / 'k'), *args],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr, proc.stderr
    assert not (tmp_path / 'k').exists()


def test_the_command_says_in_one_line_what_it_made(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'keys', '--out', str(tmp_path / 'k'),
                           '--hosts', 'world,field1'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert len(proc.stdout.strip().splitlines()) == 1 and 'world, field1' in proc.stdout
    again = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'keys', '--out', str(tmp_path / 'k'),
                            '--hosts', 'world'], capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and '--replace' in again.stderr


@pytest.mark.slow
def test_up_and_agents_refuse_a_folder_that_cannot_secure_this_host_before_anything_starts(tmp_path: Path) -> None:
    """`--secure` takes the folder of this host (its name is the host's): missing, for another host, expired, or
    without --listen, each is one line and exit 2 before any run folder or process is made."""
    keys.make(tmp_path / 'k', ['world', 'field1'])
    shutil.copytree(tmp_path / 'k' / 'field1', tmp_path / 'copied' / 'world')  # field1's keys where world's belong
    past = datetime.datetime.now(datetime.timezone.utc) - datetime.timedelta(days=40)
    keys.make(tmp_path / 'old', ['world'], days=30, now=past)
    up = ('up', '--maps', '4', '--duration', '1', '--listen', '127.0.0.1')
    cases = [
        ((*up, '--secure', str(tmp_path / 'nowhere')), 'no such folder'),
        ((*up, '--secure', str(tmp_path / 'copied' / 'world')), 'a certificate for field1, not for world'),
        ((*up, '--secure', str(tmp_path / 'old' / 'world')), 'expired on'),
        (('up', '--maps', '4', '--secure', str(tmp_path / 'k' / 'world')), 'give --listen ADDRESS too'),
        (('agents', '--join', '127.0.0.1:11850', '--ids', '1', '--secure', str(tmp_path / 'old' / 'world')),
         'expired on'),
    ]
    for n, (args, says) in enumerate(cases):
        out = tmp_path / f'run{n}'
        proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', *args, '--out', str(out)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr, \
            (args, proc.stderr)
        assert not out.exists(), f'{args}: nothing may be made before the keys are checked'


def test_the_join_line_of_a_secured_run_names_the_joining_hosts_keys(tmp_path: Path) -> None:
    """`up --secure` prints the `agents --join` line to paste on the other host: with its --secure folder."""
    from uav_flock_tools.secure import join_option
    keys.make(tmp_path / 'two', ['world', 'field1'])
    assert join_option(keys.check(tmp_path / 'two' / 'world')) == f' --secure {tmp_path / "two" / "field1"}'
    keys.make(tmp_path / 'three', ['world', 'field1', 'field2'])
    said = join_option(keys.check(tmp_path / 'three' / 'world'))
    assert said.startswith(f' --secure {tmp_path / "three" / "HOST"} (HOST: '), said
    assert join_option(None) == ''
