"""Where alerts may not be sent: addresses whose answers are secrets, not receivers.

A webhook or commit-status URL is an admin's setting, but what the server sends there and the
start of what comes back are kept in the delivery log, which makes a URL aimed at the host's own
services a way to read them. Refused: link-local addresses (169.254.169.254 and fe80::/10, where
clouds serve instance metadata and credentials), the other known metadata addresses, multicast
and unspecified ones. Loopback and private addresses stay allowed: a team's chat server or CI is
often on its own network, and tests and `redline up` post to receivers on this host. An address
is judged in every form a resolver reads as one (decimal, octal, hex IPv4; IPv4 inside IPv6;
circled or fullwidth digits and other full stops, as IDNA reads them).

Checked twice: on the literal address of a URL when it is set (a clear 422), and on every address
its host name resolves to before each delivery (a name can point anywhere). A name that resolves
to another address between the check and the connection (DNS rebinding), or that the resolver
and httpx spell differently (IDNA 2003 against 2008), is not caught.
"""

from __future__ import annotations

import ipaddress
import socket
import unicodedata

#: metadata services not on link-local addresses: AWS's over IPv6, Alibaba Cloud's
METADATA = frozenset(map(ipaddress.ip_address, ("fd00:ec2::254", "100.100.100.200")))
#: the well-known NAT64 prefix: its last 32 bits are the IPv4 address reached
NAT64 = ipaddress.IPv6Network("64:ff9b::/96")
#: the full stops IDNA separates labels with besides "." (UTS #46)
FULL_STOPS = str.maketrans(dict.fromkeys("\u3002\uff0e\uff61", "."))


def _ip(address: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """``address`` as an IP, in any form a resolver takes as one (``2852039166``, ``0251.0376``
    and ``0xa9fea9fe`` are 169.254.169.254 to ``getaddrinfo``); IPv4 carried inside IPv6
    (mapped, compatible, NAT64, 6to4) as the IPv4 it reaches; None for a name."""
    # as IDNA reads a host before any resolver sees it: compatibility forms folded (circled
    # and fullwidth digits), the other full stops taken as dots (a trial's host of ideographic
    # full stops passed the check when set; httpx connects to 169.254.169.254 for it)
    plain = unicodedata.normalize("NFKC", address.split("%", 1)[0]).translate(FULL_STOPS)
    plain = plain.removesuffix(".")  # the root's dot, which some clients drop (a trial's passed)
    try:
        ip: ipaddress.IPv4Address | ipaddress.IPv6Address = ipaddress.ip_address(plain)
    except ValueError:
        try:  # inet_aton reads the numeric forms resolvers accept: decimal, octal, hex, short
            ip = ipaddress.IPv4Address(socket.inet_aton(plain))
        except (OSError, ValueError):  # ValueError: a null character; UnicodeError is one
            return None
    if isinstance(ip, ipaddress.IPv6Address):
        carried = ip.ipv4_mapped or ip.sixtofour
        if carried is None and (int(ip) >> 32 == 0 or ip in NAT64):
            carried = ipaddress.IPv4Address(int(ip) & 0xFFFFFFFF)
        return carried or ip
    return ip


def _kind(ip: ipaddress.IPv4Address | ipaddress.IPv6Address | None) -> str | None:
    """What kind of refused address ``ip`` is; None when it is allowed (or no IP: a name)."""
    if ip is None:
        return None
    if ip in METADATA or ip.is_link_local:
        return "a link-local or cloud metadata address"
    if ip.is_multicast or ip.is_unspecified:
        return "a multicast or unspecified address"
    return None


def refused_address(address: str) -> str | None:
    """Why nothing may be sent to the literal IP ``address``; None when it may (or is no IP)."""
    ip = _ip(address)
    kind = _kind(ip)
    if kind is None:
        return None
    plain = address.split("%", 1)[0]
    return f"{address} is {kind}" if str(ip) == plain else f"{address} ({ip}) is {kind}"


def refused_host(host: str) -> str | None:
    """Why nothing may be sent to ``host`` (a name or an IP): the first of its addresses that is
    refused; None when none is, or when it does not resolve (the connection then fails and says
    so)."""
    said = refused_address(host)
    if said is not None:
        return said
    try:
        found = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except (OSError, ValueError):  # ValueError: a null character; UnicodeError is one
        return None
    for *_, sockaddr in found:
        kind = _kind(_ip(str(sockaddr[0])))
        if kind is not None:
            return f"{host} resolves to {sockaddr[0]}, {kind}"
    return None
