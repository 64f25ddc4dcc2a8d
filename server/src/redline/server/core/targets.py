"""Where alerts may not be sent: addresses whose answers are secrets, not receivers.

A webhook or commit-status URL is an admin's setting, but what the server sends there and the
start of what comes back are kept in the delivery log, which makes a URL aimed at the host's own
services a way to read them. Refused: link-local addresses (169.254.169.254 and fe80::/10, where
clouds serve instance metadata and credentials), the other known metadata addresses, multicast
and unspecified ones. Loopback and private addresses stay allowed: a team's chat server or CI is
often on its own network, and tests and `redline up` post to receivers on this host.

Checked twice: on the literal address of a URL when it is set (a clear 422), and on every address
its host name resolves to before each delivery (a name can point anywhere). A name that resolves
to another address between the check and the connection (DNS rebinding) is not caught.
"""

from __future__ import annotations

import ipaddress
import socket

#: metadata services not on link-local addresses: AWS's over IPv6, Alibaba Cloud's
METADATA = frozenset(map(ipaddress.ip_address, ("fd00:ec2::254", "100.100.100.200")))


def _kind(address: str) -> str | None:
    """What kind of refused address the IP ``address`` is; None when it is allowed (or no IP)."""
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])  # fe80::1%eth0: its zone dropped
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    if ip in METADATA or ip.is_link_local:
        return "a link-local or cloud metadata address"
    if ip.is_multicast or ip.is_unspecified:
        return "a multicast or unspecified address"
    return None


def refused_address(address: str) -> str | None:
    """Why nothing may be sent to the literal IP ``address``; None when it may (or is no IP)."""
    kind = _kind(address)
    return None if kind is None else f"{address} is {kind}"


def refused_host(host: str) -> str | None:
    """Why nothing may be sent to ``host`` (a name or an IP): the first of its addresses that is
    refused; None when none is, or when it does not resolve (the connection then fails and says
    so)."""
    said = refused_address(host)
    if said is not None:
        return said
    try:
        found = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except (OSError, UnicodeError):
        return None
    for *_, sockaddr in found:
        kind = _kind(str(sockaddr[0]))
        if kind is not None:
            return f"{host} resolves to {sockaddr[0]}, {kind}"
    return None
