"""A participant on Fast DDS's TCP transport with TLS and mutual verification, from a host's keys
(`uav-flock keys`, keys.check): the XML profile and the environment that make rmw_fastrtps use it.

The PyPI wheels' Fast DDS has no DDS-Security plugins, but its TCP transport speaks TLS (OpenSSL): a peer
whose certificate the run's CA did not sign fails the handshake and never reaches discovery. Only this
transport is given to the participant (no UDP, no shared memory). A participant that listens accepts
connections on its port; one that does not dials the listening peers it is given (docs/multihost.md).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence
from xml.sax.saxutils import escape

from .keys import CA_FILE, CERT_FILE, KEY_FILE, HostKeys

# What a handshake may be: TLS 1.2 or later, peer certificate required and verified against the run's CA.
TLS_OPTIONS = ('DEFAULT_WORKAROUNDS', 'NO_COMPRESSION', 'NO_SSLV2', 'NO_SSLV3', 'NO_TLSV1', 'NO_TLSV1_1')
VERIFY_MODES = ('VERIFY_PEER', 'VERIFY_FAIL_IF_NO_PEER_CERT')


def profile(keys: HostKeys, listen: Optional[int], peers: Sequence[tuple[str, int]] = ()) -> str:
    """The Fast DDS XML profile of a secured participant: TCPv4 with TLS only, listening on `listen` (None:
    dial only) and dialling `peers` (address, TCP port) first."""
    def path(name: str) -> str:
        return escape(str((keys.folder / name).resolve()))

    ports = f'<listening_ports><port>{int(listen)}</port></listening_ports>' if listen is not None else ''
    locators = ''.join(f'<locator><tcpv4><address>{escape(address)}</address>'
                       f'<physical_port>{int(port)}</physical_port></tcpv4></locator>' for address, port in peers)
    # An empty list is not "no list": given one, a listening participant was never reached.
    builtin = f'<builtin><initialPeersList>{locators}</initialPeersList></builtin>' if peers else ''
    verify = ''.join(f'<verify>{v}</verify>' for v in VERIFY_MODES)
    options = ''.join(f'<option>{o}</option>' for o in TLS_OPTIONS)
    return f'''<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>uav_flock_tls</transport_id>
      <type>TCPv4</type>
      {ports}
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
  <participant profile_name="uav_flock_secure" is_default_profile="true">
    <rtps>
      <userTransports><transport_id>uav_flock_tls</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
      {builtin}
    </rtps>
  </participant>
</profiles>
'''


def environment(env: dict[str, str], profile_file: Path) -> dict[str, str]:
    """A process environment whose participants take the profile: no transports of rmw's own choosing
    (LOCALHOST discovery would replace them), no discovery server, no builtin-transport override."""
    out = dict(env)
    out['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile_file)
    out['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    for key in ('FASTDDS_BUILTIN_TRANSPORTS', 'ROS_DISCOVERY_SERVER', 'ROS_STATIC_PEERS'):
        out.pop(key, None)
    return out
