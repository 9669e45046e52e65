"""A run's participants on Fast DDS's TCP transport with TLS and mutual verification, from a host's keys
(`uav-flock keys`, keys.check): the XML profiles and the environment that make rmw_fastrtps use them
(`up --secure`, `agents --secure`, docs/multihost.md).

The PyPI wheels' Fast DDS has no DDS-Security plugins, but its TCP transport speaks TLS (OpenSSL): a peer
whose certificate the run's CA did not sign fails the handshake and never reaches discovery. Only this
transport is given to a participant (no UDP, no shared memory). The run's discovery server listens on the
world host's address; every other participant is its client (the recorder, the live view and `echo` its
super-clients, which hear of every endpoint) and listens on a TCP port of its own that the OS picks: TCP
needs one side of each pair of participants to accept, and two that only dial never meet.

Fast DDS 2.14 verifies only the peers it dials: it sets a connection's verify mode after the handshake of a
connection it accepted, so the profile's verify mode alone lets a stranger who dials in with no certificate
join (tried: it heard a member's topic). The certificate is required on every side by OpenSSL's own
configuration (OPENSSL_CONF, its system_default section: VerifyMode Require), which applies to every TLS
context the participant's OpenSSL makes, the accepting one included; verified against the run's CA, which
the profile gives (verify_file).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional
from xml.sax.saxutils import escape

from .keys import CA_FILE, CERT_FILE, KEY_FILE, HostKeys

# What a handshake may be: no TLS below 1.2, peer certificate verified against the run's CA (Fast DDS applies one
# verify flag of the list, the first it knows, and only on connections it dials: OPENSSL_CONFIG does the rest).
TLS_OPTIONS = ('DEFAULT_WORKAROUNDS', 'NO_COMPRESSION', 'NO_SSLV2', 'NO_SSLV3', 'NO_TLSV1', 'NO_TLSV1_1')
VERIFY_MODES = ('VERIFY_PEER',)
# OpenSSL's configuration for a participant's process: every TLS context it makes requires and verifies the peer's
# certificate, whichever side of the connection it is on (SSL_CONF_cmd: VerifyMode; Peer for a client, Require for a
# server). TLS 1.2 only: under 1.3 a dialler counts the handshake done before the listener has checked its
# certificate, and a run over three hosts stalled with no agent of the joining hosts seen in 300 s (tried).
OPENSSL_CONFIG = """openssl_conf = uav_flock_openssl
[uav_flock_openssl]
ssl_conf = uav_flock_ssl
[uav_flock_ssl]
system_default = uav_flock_tls
[uav_flock_tls]
VerifyMode = Peer,Request,Require
MinProtocol = TLSv1.2
MaxProtocol = TLSv1.2
"""
OPENSSL_FILE = 'openssl.cnf'  # beside the profiles
# The GUID prefix Fast DDS gives discovery server 0 (`fast-discovery-server -i 0`, ROS_DISCOVERY_SERVER).
SERVER_PREFIX = '44.53.00.5f.45.50.52.4f.53.49.4d.41'
ROLES = ('server', 'client', 'super_client')
FOLDER = 'secure'  # in a run folder: one profile per role, <role>.xml


def _locator(address: str, port: int) -> str:
    return (f'<locator><tcpv4><address>{escape(address)}</address><physical_port>{int(port)}</physical_port>'
            f'<port>{int(port)}</port></tcpv4></locator>')


def profile(keys: HostKeys, role: str, server: tuple[str, int]) -> str:
    """The Fast DDS XML profile of a participant of a secured run: TCPv4 with TLS only; the discovery server
    (role 'server') listening at `server` (address, TCP port), any other ('client', 'super_client') dialling
    it and listening on a port of the OS's choice. No Nagle: lockstep's small messages each waited for an
    acknowledgement (10 steps/s of 12 MAPs over three hosts, 31 without)."""
    if role not in ROLES:
        raise ValueError(f'{role}: not one of {", ".join(ROLES)}')

    def path(name: str) -> str:
        return escape(str((keys.folder / name).resolve()))

    here = _locator(*server)
    if role == 'server':
        listen, discovery = server[1], (
            f'<prefix>{SERVER_PREFIX}</prefix><builtin><discovery_config><discoveryProtocol>SERVER'
            f'</discoveryProtocol></discovery_config><metatrafficUnicastLocatorList>{here}'
            f'</metatrafficUnicastLocatorList></builtin>')
    else:
        listen, discovery = 0, (
            f'<builtin><discovery_config><discoveryProtocol>{role.upper()}</discoveryProtocol>'
            f'<discoveryServersList><RemoteServer prefix="{SERVER_PREFIX}"><metatrafficUnicastLocatorList>{here}'
            f'</metatrafficUnicastLocatorList></RemoteServer></discoveryServersList></discovery_config></builtin>')
    verify = ''.join(f'<verify>{v}</verify>' for v in VERIFY_MODES)
    options = ''.join(f'<option>{o}</option>' for o in TLS_OPTIONS)
    return f'''<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>uav_flock_tls</transport_id>
      <type>TCPv4</type>
      <listening_ports><port>{listen}</port></listening_ports>
      <enable_tcp_nodelay>true</enable_tcp_nodelay>
      <tls>
        <private_key_file>{path(KEY_FILE)}</private_key_file>
        <cert_chain_file>{path(CERT_FILE)}</cert_chain_file>
        <verify_file>{path(CA_FILE)}</verify_file>
        <verify_mode>{verify}</verify_mode>
        <options>{options}</options>
        <handshake_role>DEFAULT</handshake_role>
      </tls>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="uav_flock_{role}" is_default_profile="true">
    <rtps>
      <userTransports><transport_id>uav_flock_tls</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
      {discovery}
    </rtps>
  </participant>
</profiles>
'''


def write_profiles(keys: HostKeys, server: tuple[str, int], folder: Path,
                   roles: tuple[str, ...] = ROLES) -> dict[str, Path]:
    """One profile a role in folder (created, readable by its owner only: they name the key's path), and
    OpenSSL's configuration beside them (OPENSSL_CONFIG)."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    (folder / OPENSSL_FILE).write_text(OPENSSL_CONFIG)
    paths = {}
    for role in roles:
        paths[role] = folder / f'{role}.xml'
        paths[role].write_text(profile(keys, role, server))
    return paths


def environment(env: dict[str, str], profile_file: Optional[Path]) -> dict[str, str]:
    """A process environment whose participants take the profile (written by write_profiles, OpenSSL's
    configuration beside it): no transports of rmw's own choosing (LOCALHOST discovery would replace them), no
    discovery server or super-client flag of the environment's (the profile names them), no builtin-transport
    override. None: env as it is."""
    if profile_file is None:
        return env
    out = dict(env)
    out['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile_file)
    out['OPENSSL_CONF'] = str(profile_file.parent / OPENSSL_FILE)
    out['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    for key in ('FASTDDS_BUILTIN_TRANSPORTS', 'ROS_DISCOVERY_SERVER', 'ROS_STATIC_PEERS', 'ROS_SUPER_CLIENT'):
        out.pop(key, None)
    return out


def role_profile(run: Path, keys: Optional[HostKeys], role: str) -> Optional[Path]:
    """The profile of a participant of that role (ROLES) in a run's folder, None if the run is not secured."""
    return run / FOLDER / f'{role}.xml' if keys is not None else None


def role_env(env: dict[str, str], run: Path, keys: Optional[HostKeys], role: str) -> dict[str, str]:
    """The environment of a participant of that role in a run (env as it is if the run is not secured)."""
    return environment(env, role_profile(run, keys, role))


def for_run(keys: HostKeys, server_address: str, run: Path) -> dict[str, str]:
    """A secured run's profiles, written into its folder; what its run.json says of them (`echo --run` takes the
    super-client's)."""
    host, port = server_address.rsplit(':', 1)
    write_profiles(keys, (host, int(port)), run / FOLDER)
    return {'ca': keys.ca_fingerprint, 'super_client': str(run / FOLDER / 'super_client.xml')}


def join_option(keys: Optional[HostKeys]) -> str:
    """The `--secure` a joining host's `agents` needs: its own folder beside this host's (named if it is the only
    other one there)."""
    if keys is None:
        return ''
    others = sorted(d for d in keys.folder.parent.iterdir() if d.is_dir() and d != keys.folder) \
        if keys.folder.parent.is_dir() else []
    return f' --secure {others[0] if len(others) == 1 else keys.folder.parent / "HOST"}' + \
        ('' if len(others) == 1 else ' (HOST: that host\'s folder of `uav-flock keys`)')


def banner(keys: HostKeys) -> str:
    """What `up` says of a secured run: the transport, and the CA by folder and fingerprint."""
    return (f'secured: TCP with TLS only, peers verified against the CA of {keys.folder} '
            f'(SHA-256 {keys.ca_fingerprint[:23]}...)')
