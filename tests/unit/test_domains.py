"""ROS_DOMAIN_ID claims: two runs on one host never share a domain, whatever the random draw."""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
from uav_flock_tools import domains
from uav_flock_tools.domains import FRESH_DOMAINS, DomainInUse, claim_domain

HOLDER = '''
import sys, time
from uav_flock_tools.domains import claim_domain
claim = claim_domain()
print(claim.domain, flush=True)
time.sleep(300)
'''


@pytest.fixture
def own_claims(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A claim folder of the test's own: any other uav-flock run on the host claims and dates domains in the
    host-wide one while the test counts on their order."""
    monkeypatch.setattr(domains, 'DOMAIN_CLAIMS', tmp_path / 'claims')
    return tmp_path / 'claims'


def test_fresh_claims_never_share_a_domain_until_none_is_left(own_claims: Path) -> None:
    held = []
    try:
        with pytest.raises(DomainInUse, match='every ROS_DOMAIN_ID from 1 to 101 is in use'):
            for _ in range(len(FRESH_DOMAINS) + 1):
                held.append(claim_domain())
        domains = [c.domain for c in held]
        assert len(set(domains)) == len(domains) and set(domains) <= set(FRESH_DOMAINS)
        freed = held.pop()
        freed.release()
        again = claim_domain()
        held.append(again)
        assert again.domain == freed.domain, 'a released domain is free again'
    finally:
        for c in held:
            c.release()


def test_a_fresh_claim_takes_the_least_recently_used_domain(own_claims: Path) -> None:
    """A SIGKILLed run's participants stay in discovery for their lease: the domain it just left is the last
    to be handed out again, not one in a hundred."""
    used = []
    for _ in range(len(FRESH_DOMAINS)):
        with claim_domain() as domain:
            used.append(domain)
    assert sorted(used) == list(FRESH_DOMAINS), 'every domain is used once before any is used twice'
    with claim_domain() as domain:
        assert domain == used[0]
    assert sorted(int(p.name) for p in own_claims.iterdir()) == list(FRESH_DOMAINS), 'claimed in the own folder'


def test_a_domain_held_by_another_process_is_refused_and_freed_when_it_dies(tmp_path: Path) -> None:
    holder = subprocess.Popen([sys.executable, '-c', HOLDER], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None
        domain = int(holder.stdout.readline())
        with pytest.raises(DomainInUse, match=f'ROS_DOMAIN_ID {domain} is in use'):
            claim_domain(domain)
        up = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'up', '--maps', '2', '--domain-id',
                             str(domain), '--out', str(tmp_path)], capture_output=True, text=True, timeout=120)
        assert up.returncode == 2 and up.stderr.strip().count('\n') == 0 and 'is in use' in up.stderr, up.stderr
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=30)
        with claim_domain(domain) as claimed:  # the kernel dropped the dead holder's claim: nothing stale
            assert claimed == domain
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
